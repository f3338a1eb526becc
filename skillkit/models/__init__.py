"""Kernels, GP forward models, trajectory sampling, moment matching, kernel embeddings."""
