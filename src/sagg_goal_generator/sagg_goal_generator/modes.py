"""Goal modes: how a goal was chosen (the values of the sagg_msgs/Goal MODE_* constants). ROS-free.

The teachers beyond the paper reuse them: a goal drawn from the part of Y a teacher's interest
chose (a mixture component, a grid cell) is ``region``; a goal of a teacher's uniform share is
``global``; a goal of a teacher's initial random phase is ``initial``."""

MODE_INITIAL, MODE_REGION, MODE_GLOBAL, MODE_LOW_COMPETENCE, MODE_RANDOM = 0, 1, 2, 3, 4
MODE_NAMES = {MODE_INITIAL: "initial", MODE_REGION: "region", MODE_GLOBAL: "global",
              MODE_LOW_COMPETENCE: "low-competence", MODE_RANDOM: "random"}
