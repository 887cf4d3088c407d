"""Representation heads, one file each. Every module here is imported by the head registry."""
