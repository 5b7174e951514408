"""Analysis of recorded episodes: replay fidelity, statistics."""
