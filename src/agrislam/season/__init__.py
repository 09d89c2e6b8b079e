"""A survey that continues a saved map (issue 15): the map as prior (map.py), finding the
robot in it from the first frames (relocalise.py), the back end that brings saved plants
into the graph when they are seen again (backend.py), and what changed (changes.py)."""
