"""One-step memory agents: the main recipe with the previous observation and move as input."""
