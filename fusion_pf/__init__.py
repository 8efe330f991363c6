"""fusion-pf: RGB-D palm tracking with a data-fusion particle filter (paper 003)."""

__version__ = "0.1.0"
