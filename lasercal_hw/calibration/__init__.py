"""The calibration mathematics: measurement model, initial solution, solver, the paper's
formulation, simulation, quality gates, the result and observations.csv."""
