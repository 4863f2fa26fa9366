"""Reading and writing drives: route and pose files (:mod:`.routes`), ROS bags (:mod:`.bags`)
and routes or logs by URL (:mod:`.remote`)."""
