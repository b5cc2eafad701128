"""Training: the paper's models, the pre-training corpus and the training loop (torch)."""
