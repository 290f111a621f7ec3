"""Readers and writers: KITTI layout, custom layout, Blickfeld .bfpc, PCD / PLY / NPY, CVAT import; the input formats
that import, detect and site backgrounds read are registered in io.formats."""
