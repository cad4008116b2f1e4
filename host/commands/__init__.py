"""host/commands."""
