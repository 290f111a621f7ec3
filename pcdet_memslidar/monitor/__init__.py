"""Live use of a trained detector: detections of recordings, tracks across frames, safety zones and events."""
