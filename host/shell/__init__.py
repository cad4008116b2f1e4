"""host/shell."""
