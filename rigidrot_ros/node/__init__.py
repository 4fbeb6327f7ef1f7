"""ROS 2 glue: the attitude node and message conversion (the core knows nothing of it)."""
