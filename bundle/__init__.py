"""Aerial triangulation: tie points (pycolmap), initial orientation, bundle adjustment, blunders, pipeline."""
