"""``python -m ccf_ros.node``: ``ccf_node``."""

from .entry import main

main()
