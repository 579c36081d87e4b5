"""Surveys: from geotagged survey photos to a georeferenced model, DSM, orthophoto and a flyable map."""
