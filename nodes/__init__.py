"""touch4d."""
