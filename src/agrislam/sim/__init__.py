"""The field simulator: a stand-in for the paper's Gazebo world (sec. 3.1) that yields the
same records as a recorded survey log. `Simulator(SimConfig()).records()` is the default
400-plant run; `sources.open_source("sim:")` opens it as a source, `sinks.jsonl.write_log`
records it.

`ArenaSimulator(ArenaConfig()).records()` (arena.py) is the other scenario: robots driving
random paths among point landmarks in a small indoor arena; `ArenaConfig.realistic()` makes it
behave like the real multi-robot log it stands for, with a real sensor's effects
(`effects_config.py`), which the field simulator can have too."""
