"""Reinforcement learning over map bundles. Reads cities through ``dataset`` only, never raw files."""
