"""Numbers from recordings: summaries (``larns info``, the fleet's final table) and the report's metrics."""
