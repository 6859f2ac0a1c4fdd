"""Simulated serial laser scanners on pseudo-terminals, for tests and ``vmp live --simulate``.

Each device answers its protocol's commands as the real one does and streams scans ray-cast
from a scenario; it can corrupt bytes at a given rate and go silent or power-cycle on request.
"""
