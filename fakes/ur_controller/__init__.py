"""Fake Universal Robots controller: dashboard (29999), RTDE (30004) and script (30003)
servers that the unmodified ur_rtde 1.6.5 client accepts, on a loopback address."""
