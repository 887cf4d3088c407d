"""Analyses of the paper's claims that need no training (continuity of representations)."""
