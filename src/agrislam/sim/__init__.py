"""The field simulator: a stand-in for the paper's Gazebo world (sec. 3.1) that yields the
same records as a recorded survey log. `Simulator(SimConfig()).records()` is the default
400-plant run; `record_simulation(cfg, path)` writes it as JSONL."""
