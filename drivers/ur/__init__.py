"""Universal Robots arms through the unmodified ur_rtde library."""
