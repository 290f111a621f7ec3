"""MEMSLidarDataset, augmentation, voxelisation and sim/real mixing (OpenPCDet's DatasetTemplate contract)."""
