"""Reading and writing drives: route and pose files (:mod:`.routes`), ROS bags (:mod:`.bags`),
comma2k19 segment folders (:mod:`.comma2k19`) and routes or logs by URL (:mod:`.remote`)."""
