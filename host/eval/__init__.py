"""host/eval."""
