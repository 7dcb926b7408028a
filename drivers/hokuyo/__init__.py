"""Hokuyo SCIP 2.0: pure codec, byte transports and the scanner client."""
