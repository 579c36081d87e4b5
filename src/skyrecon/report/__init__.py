"""Figures and HTML reports for people to look at."""
