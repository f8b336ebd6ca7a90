"""Tests of periodic orbits, continuation, grazing curves and bifurcations (`grazejax/_orbits/`)."""
