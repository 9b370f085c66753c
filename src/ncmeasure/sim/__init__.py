"""Simulated drives and signal sources: stand-ins for real hardware in tests and the demo."""
