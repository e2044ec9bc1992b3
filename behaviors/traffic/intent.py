"""Which lane each agent heads for: its wish (the policy's steer as the motives leave it) and the
change that wish begins or the one under way goes on with, within the lanes the limits leave open."""

from __future__ import annotations

import numpy as np

from behaviors.traffic.motives.wishes import LaneWishes
from behaviors.traffic.scene import RoadPlace
from behaviors.traffic.settings import LaneDriving


def lane_wish(
    wishes: LaneWishes, place: RoadPlace, lateral: LaneDriving, leave: np.ndarray | None
) -> np.ndarray:
    """[N] int: the lane each agent wishes for (+1 the fast side, -1 the slow side, 0 its own): its
    steer beyond `change_threshold`. Where the rules judge the lanes (`wishes.slow_side_free` given),
    a wish for a lane that is not there is no wish, a wish for the fast side counts only where
    `held_up`, and no wish means keeping right where that lane is free; a car whose own lane ends
    wishes for the side `leave` [N] (+1/-1, 0: none) says, whatever the steer."""
    steer, threshold = wishes.steer, lateral.change_threshold
    wish = np.where(steer > threshold, 1, np.where(steer < -threshold, -1, 0))
    if wishes.slow_side_free is not None:
        possible = np.where(wish > 0, place.lanes_fast > 0, np.where(wish < 0, place.lanes_slow > 0, True))
        may_pass = np.ones(len(wish), bool) if wishes.held_up is None else wishes.held_up
        wish = np.where(possible & ((wish <= 0) | may_pass), wish, 0)
        wish = np.where((wish == 0) & wishes.slow_side_free, -1, wish)
    if leave is not None:
        wish = np.where(leave != 0, leave, wish)
    return wish


def lane_intent(
    wish: np.ndarray,
    changing: np.ndarray,
    place: RoadPlace,
    open_lanes: np.ndarray,
    give_up: np.ndarray | None,
    lateral: LaneDriving,
) -> np.ndarray:
    """[N] int: the lane each agent heads for, relative to its own (+1 the fast side, -1 the slow
    side, 0 its own), given its `wish` and `changing`, the same at the last step. A change begins
    only where that side's lane exists and is open (`open_lanes` [N, 2]: fast, slow; the limits'
    vetoes); until then the wish waits. A change under way is given up where `give_up` [N] bool
    (`limits.lost_gap`). No change begins where `place.may_begin` is False (inside a junction, whose
    lanes are a connection's, not the carriageway's: SUMO's lane numbers and neighbours there are no
    guide). Otherwise a change under way goes on whatever the wish: a policy that could call changes
    off learnt to start one and call it off at the next step, riding beside the line.

    A change is over once the car's centre is `arrived` lane widths on the far side of its new
    lane's centre line, which is where SUMO puts it right after it crossed the line (its offset
    jumps from +w/2 to -w/2): no lane index is needed, so this holds across edges too. A car that
    still wishes the same way then goes on to the next lane in one move: the test stays true until
    it leaves the line behind, and restarting the change at every other step swung its target
    between the two lanes.
    """
    lanes_fast, lanes_slow = place.lanes_fast, place.lanes_slow
    crossed = changing * place.lane_offset < -lateral.arrived * place.lane_width
    vanished = np.where(changing > 0, lanes_fast == 0, np.where(changing < 0, lanes_slow == 0, False))
    going = np.where(crossed | vanished, 0, changing)
    if give_up is not None:
        going = np.where(give_up, 0, going)
    room = np.where(wish > 0, (lanes_fast > 0) & open_lanes[:, 0], (lanes_slow > 0) & open_lanes[:, 1])
    if place.may_begin is not None:
        room &= place.may_begin
    begins = (changing == 0) | ((going == 0) & (wish == changing))
    return np.where(begins & (wish != 0) & room, wish, going)
