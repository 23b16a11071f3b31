"""ccf_ros: cascaded complementary filter for IMU orientation."""
__version__ = "0.1.0"
