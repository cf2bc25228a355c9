"""Unit tests of trq_params, named after the module each tests."""
