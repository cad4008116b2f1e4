"""Multi-turn chat with the robot: conversation loop, observation messages, batch chat files."""
