"""geocom/dispatch.py: every procedure the simulator accepts (it has a signature) is answered by something: a
motion, an angle reply, the coordinate reply or a handler of the table; none falls through to an internal error."""

from aruco_abs_orient.geocom import dispatch
from aruco_abs_orient.geocom.protocol import Rpc


def test_every_accepted_procedure_has_an_answer():
    answered = set(dispatch._MOTIONS) | set(dispatch._ANGLE_RPCS) | {Rpc.TMC_GetCoordinate} | set(dispatch._HANDLERS)
    missing = sorted(set(dispatch._SIGNATURES) - answered)
    assert not missing, f"procedures with a signature but no answer: {missing}"
    assert not set(dispatch._HANDLERS) - set(dispatch._SIGNATURES), "a handler the dispatch never reaches"
