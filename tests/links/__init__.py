"""Tests of the drive links."""
