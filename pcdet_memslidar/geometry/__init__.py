"""Box geometry, coordinate transforms, rotated IoU and NMS."""
