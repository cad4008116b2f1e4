"""host/motion: turning targets into timed servo frames (trajectories, mixing)."""
