"""pcdet-memslidar: privacy-friendly person detection with MEMS-LiDAR, OpenPCDet-compatible."""
import re
from pathlib import Path

from setuptools import find_packages, setup

VERSION = re.search(r'__version__ = "(.+)"', Path(__file__).with_name("pcdet_memslidar").joinpath("__init__.py").read_text()).group(1)

setup(
    name="pcdet-memslidar",
    version=VERSION,
    description="MEMS-LiDAR simulation, datasets and a CPU-capable SECOND person detector, compatible with OpenPCDet",
    long_description=Path(__file__).with_name("README.md").read_text(),
    long_description_content_type="text/markdown",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(include=["pcdet_memslidar", "pcdet_memslidar.*"]),
    package_data={"pcdet_memslidar": ["assets/*", "assets/**/*"]},
    install_requires=[
        "torch>=2.5",  # safe_globals (OpenPCDet checkpoints); install torch==2.13.0 (CPU wheel) first: see run.sh
        "numpy>=1.24",
        "numba>=0.60",  # the simulator's per-ray loops (sim/body_rays.py)
        "spconv>=2.3.6",
        "easydict>=1.10",
        "pyyaml>=6.0",
        "scipy>=1.10",
        "tensorboardX>=2.6",
        "open3d>=0.18",
        "libusb-package>=1.0.26",  # ships libusb-1.0.so.0, which the open3d wheel links against
        "tqdm>=4.60",
        "matplotlib>=3.7",
        "python-neo-lzf>=0.3.5",  # LZF (C, BSD) for PCD DATA binary_compressed
    ],
    extras_require={"test": ["pytest>=7", "shapely>=2.0"]},
    entry_points={"console_scripts": ["memslidar=pcdet_memslidar.cli:main"]},
)
