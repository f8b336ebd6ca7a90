"""Dynamics at scale through impacts: sections, orbit diagrams, Lyapunov spectra, basins."""
