"""A robot on the host: its interface bound to behaviours, and the runtime that moves it over the link."""
