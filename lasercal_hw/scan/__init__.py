"""Scans: beam-by-beam averaging and finding the rod's centre in an averaged scan."""
