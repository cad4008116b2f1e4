"""host/link."""
