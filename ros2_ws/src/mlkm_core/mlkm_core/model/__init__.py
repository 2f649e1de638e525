"""The traffic model a link is scored with: motion models (``motion``, ``kalman``) and the
cues (``cues``, one module each: ``lane``, ``length``, ``lane_order``; registered in
``catalogue``), composed by ``link.LinkModel``. ROS-free; it imports nothing from the
associators that use it."""
