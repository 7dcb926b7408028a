"""The calibration daemon (``lasercal serve``): jobs over HTTP, live events, calibration history."""
