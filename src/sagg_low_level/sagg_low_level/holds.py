"""The learner's holds (ROS-free): why no new command may go out now, one entry per cause.

A hold is set with its reason in words and released by its cause alone; while any is set the learner
sends no new command (the command in flight, if any, completes and its sample is stored). The causes:

======================  =====================================================  ================================
key                     set when                                               released when
======================  =====================================================  ================================
``service``             ``/sagg/pause`` true                                   ``/sagg/pause`` false
``driver``              no valid joint state / task point for                  both fresh again, /joint_states
                        ``joint_state_timeout`` s, or /joint_states has no     published
                        publisher
``joint_states``        ``plausibility.hold_after`` rejected joint states      the next valid one
                        in a row
``task_point``          the same for task points                               the next valid one
``sources <topic>``     a second source sends what the learner uses            one source quiet for
                                                                               ``plausibility.source_grace`` s
                                                                               and a message of the other taken
``follow``              the arm does not follow its setpoints for              a probe setpoint moved it
                        ``follow_timeout`` s (protective stop, e-stop)         (every ``follow_retry`` s)
``reach``               a ``/sagg/reach`` goal waits or is being reached       the last queued reach is over
``fault``               the learner produced an invalid command                never (a bug: see /diagnostics)
======================  =====================================================  ================================

During a reach the ``reach`` hold itself and a pause by ``/sagg/pause`` do not block (the reach's own
commands go out: a reach asked for while learning is paused is a deliberate request, e.g. the evaluation
on the robot pauses learning and then reaches its test goals); every other hold does.
"""
from __future__ import annotations

from typing import Callable

SERVICE, DRIVER, JOINT_STATES, TASK_POINT, REACH, FAULT = ("service", "driver", "joint_states", "task_point",
                                                           "reach", "fault")
FOLLOW = "follow"

SOURCES = "sources "  # + the topic
# the reason of the SERVICE hold (on /sagg/status: a run's orchestrator tells a user's pause from a stall by it)
PAUSED_BY_SERVICE = "paused by the /sagg/pause service"
# holds that are no fault of the graph (a user's pause, a reach): not reported as a fault on /diagnostics,
# and not in the way of a reach's own commands
NOT_FAULTS = (SERVICE, REACH)


class Holds(dict):
    """Hold key -> reason in words (the table above). :meth:`set` logs a new or changed reason
    (``warn``), :meth:`release` logs the release (``info``) and returns whether one was set."""

    def __init__(self, warn: Callable[[str], None], info: Callable[[str], None]):
        super().__init__()
        self._warn, self._info = warn, info

    def set(self, key: str, reason: str) -> None:
        if self.get(key) != reason:
            self._warn(f"pausing: {reason}")
        self[key] = reason

    def release(self, key: str) -> bool:
        if self.pop(key, None) is None:
            return False
        self._info(f"{key} hold released" + (": resuming" if not self else ""))
        return True

    def blocking(self, reaching: bool) -> bool:
        """Whether a new command must wait (during a reach its own hold and a pause do not count)."""
        return any(k not in NOT_FAULTS for k in self) if reaching else bool(self)

    def faults(self) -> str:
        """The holds that are a fault of the graph (not a pause or a reach), in words."""
        return "; ".join(v for k, v in self.items() if k not in NOT_FAULTS)
