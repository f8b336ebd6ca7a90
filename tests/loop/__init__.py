"""Tests of the impact loop's own modules (`grazejax/_loop/`)."""
