"""The packages: every pcdet_memslidar package setuptools finds, plus the repository's cfgs/ shipped as
pcdet_memslidar.cfgs, so that an installed package (not only a checkout) finds its configs (config.CONFIG_DIR).
Everything else is in pyproject.toml."""
from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["pcdet_memslidar", "pcdet_memslidar.*"]), "pcdet_memslidar.cfgs"],
      package_dir={"pcdet_memslidar.cfgs": "cfgs"})
