"""Reproduction runner: table specs, jobs, training/evaluation orchestration and reports."""
