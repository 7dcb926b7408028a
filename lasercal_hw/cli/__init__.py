"""The ``lasercal`` command line."""
