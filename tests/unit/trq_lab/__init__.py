"""Unit tests of trq_lab, named after the module each tests."""
