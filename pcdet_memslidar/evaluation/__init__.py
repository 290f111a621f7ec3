"""Average precision of the person class (3D / BEV IoU 0.5, R40 / R11, distance bins), reports, figures."""
