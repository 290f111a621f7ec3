"""MEMS-LiDAR simulator: scan pattern, sensor physics, people, scenes, ray casting, domain presets, writer."""
