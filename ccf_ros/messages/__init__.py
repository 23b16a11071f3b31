"""Message code shared by the node, ``ccf replay`` and the fleet; no ROS or rosbags import.

:mod:`.cdr` reads and patches the fields of little-endian CDR messages; :mod:`.convert` holds the rules for message
fields (stamps, filling an Imu); :mod:`.paths` the two ways a message goes (bytes or deserialized), one protocol.
"""

__all__ = ['cdr', 'convert', 'paths']
