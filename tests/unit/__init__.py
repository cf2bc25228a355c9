"""Unit tests: pure functions and single objects against hand-computed values, one folder per
package, one file per module tested (tests/meta/test_tiers.py holds the layout)."""
