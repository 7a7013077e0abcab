"""Kinds of competence report (the values of the sagg_msgs/CompetenceReport KIND_* constants):
what the low level reports and the high level reads. ROS-free."""

KIND_GOAL, KIND_SUBGOAL, KIND_REACHED, KIND_EXPLORATION = 0, 1, 2, 3
KIND_NAMES = {KIND_GOAL: "goal", KIND_SUBGOAL: "subgoal", KIND_REACHED: "reached",
              KIND_EXPLORATION: "exploration"}
