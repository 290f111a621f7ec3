"""Point feature encoding and data processing (range mask, shuffle, voxelisation)."""
from .data_processor import DataProcessor, take_points
from .point_feature_encoder import PointFeatureEncoder

__all__ = ["DataProcessor", "PointFeatureEncoder", "take_points"]
