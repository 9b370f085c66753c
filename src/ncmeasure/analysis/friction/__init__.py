"""Friction from the windows: the table of the current per step, and the models fitted to it."""
