"""Laser milestones: signatures (ED, CCA, DCT, HWT), matching, the milestone manager and store.

NumPy arrays in, matches out; this package imports nothing of the rest of the project.
"""
