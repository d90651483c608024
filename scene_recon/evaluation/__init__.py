"""Evaluation against ground truth (tool layer): 3D panoptic quality of maps, contact-graph metrics."""
