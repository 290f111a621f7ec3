"""Small helpers shared by every stage: atomic writes, Open3D import, threads."""
