"""pcdet-memslidar: MEMS-LiDAR simulation, datasets and SECOND person detection, OpenPCDet-compatible.

Importing it changes nothing in the process: the entry points apply the process-wide settings
(policy.apply_process_policy).
"""

__version__ = "0.2.0"
