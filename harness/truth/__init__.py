"""Truth engine: vehicle and scenario files, road and friction map, tires, driver, the MuJoCo car and its simulation, truth signals and events."""
