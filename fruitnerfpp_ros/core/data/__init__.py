"""Datasets: the transforms.json format, loading images/masks/poses, scene bounds, ray batches."""
