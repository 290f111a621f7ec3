"""Whole experiments: the paper's reproduction (reproduce), its open questions (sweeps) and a detector for a site
(site_detector), with the training runs they share (runs) and their reports with the paper's numbers (report)."""
