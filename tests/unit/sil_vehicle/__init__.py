"""Unit tests of sil_vehicle, named after the module each tests."""
