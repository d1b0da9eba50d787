"""Simulated-query benchmark: query simulation, methods, the resumable runner and the paper's report."""
