"""Wire-faithful fake devices (SCIP scanner, UR controller) and the world they share."""
