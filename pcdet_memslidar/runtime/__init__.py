"""Training (train.train) and prediction (predict.predict) of a detector, their loops, checkpoints, distributed
training."""
