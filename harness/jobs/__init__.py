"""Jobs: the commands' work (run pipeline, check, stress, replay, compare, falsify) and their worker pools."""
