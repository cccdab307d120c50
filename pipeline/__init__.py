"""Everything that produces or consumes score matrices: the command line, stores, planners."""
