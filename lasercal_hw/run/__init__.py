"""One calibration run, live or replayed: sequencer, preflight, dwell, device protocols,
the dry-run cell process, outputs, resume and replay."""
