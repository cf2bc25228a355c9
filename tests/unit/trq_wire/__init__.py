"""Unit tests of trq_wire, named after the module each tests."""
