"""Unit tests of trq_offboard, named after the module each tests."""
