"""A survey that continues a saved map: the map as prior (prior_map.py), finding the robot in
it from the first frames (relocalise.py), the back end that brings saved plants into the
graph when they are seen again (prior_backend.py), and what changed (changes.py)."""
