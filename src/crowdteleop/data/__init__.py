"""Demonstration data: recording, storage, video."""
