"""Scoring predictions: metrics, baselines, previews."""
