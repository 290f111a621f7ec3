"""Training and evaluation loops, checkpoints, distributed training."""
