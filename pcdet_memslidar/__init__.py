"""pcdet-memslidar: MEMS-LiDAR simulation, datasets and SECOND person detection, OpenPCDet-compatible."""
__version__ = "0.2.0"
