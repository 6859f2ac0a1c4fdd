"""Rerun views of the map being assembled; plain arrays in, imports nothing of ``vmp``."""
