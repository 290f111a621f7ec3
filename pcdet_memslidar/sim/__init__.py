"""MEMS-LiDAR simulator: scan pattern, sensor physics, people, scenes, sites, ray casting, compositing into real
recordings, writer."""
