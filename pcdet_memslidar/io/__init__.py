"""Readers and writers: KITTI layout, custom layout, Blickfeld .bfpc, PCD / PLY / NPY, CVAT import."""
