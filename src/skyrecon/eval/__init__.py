"""Evaluation against ground truth: metrics and reference geometry built from known cameras."""
