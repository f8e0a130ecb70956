"""Sparse worlds: a brick table on the host, brick pools on the device, and the dense world's
algorithms run over gathered scratch boxes (``world.py`` says how)."""
