"""The learning run in one process, without ROS (``sagg experiment``), and the ROS-free parts every
run shares: the arm's config and graph parameters, evaluation, phases, result.json."""
