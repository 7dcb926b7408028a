"""The physical model of a Hokuyo UTM-30LX-EW (docs/scanner-model.md).

``physical.PhysicalScanner`` is what ``fakes.world.World`` uses when a scene says
``model = "physical"`` (the default); ``dwell.simulate_dwell`` makes a dwell's raw scans
of a rod in front of a wall, for extraction tests and benchmarks.
"""
