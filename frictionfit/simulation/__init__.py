"""Synthetic data with known truth: single trials, rubbing measurements, gestures, hard cases."""
