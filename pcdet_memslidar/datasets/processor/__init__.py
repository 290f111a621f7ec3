"""Point feature encoding and data processing (range mask, shuffle, voxelisation)."""
from pcdet_memslidar.datasets.processor.data_processor import DataProcessor, take_points
from pcdet_memslidar.datasets.processor.point_feature_encoder import PointFeatureEncoder

__all__ = ["DataProcessor", "PointFeatureEncoder", "take_points"]
