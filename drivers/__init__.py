"""Talking to hardware: the Hokuyo SCIP 2.0 scanner and the UR robot over ur_rtde."""
