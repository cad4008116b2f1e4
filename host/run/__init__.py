"""Running a task end to end: board process, link, shell, artefacts."""
