"""Errors raised while flying: each names the command or wait and the vehicle."""

from __future__ import annotations


class MavlinkError(Exception):
    """Something a vehicle did or did not do (not bad user input: see swarmctl.errors.InputError)."""


class CommandRejected(MavlinkError):
    """The vehicle answered a command with DENIED, FAILED, UNSUPPORTED or TEMPORARILY_REJECTED."""

    def __init__(self, command: str, vehicle: str, result: str, reason: str = ""):
        self.command, self.vehicle, self.result, self.reason = command, vehicle, result, reason
        why = f" ({reason})" if reason else ""
        super().__init__(f"{vehicle}: {command} was refused: {result}{why}")


class CommandTimeout(MavlinkError):
    """No COMMAND_ACK after all retries."""

    def __init__(self, command: str, vehicle: str, attempts: int, timeout: float):
        self.command, self.vehicle, self.attempts = command, vehicle, attempts
        detail = f"after {attempts} attempts ({timeout:g} s each)" if attempts else "(MAVSDK's own retries timed out)"
        super().__init__(f"{vehicle}: no answer to {command} {detail}")


class WaitTimeout(MavlinkError):
    """A state the vehicle should reach (ready, altitude, position, landed) was not reached in time."""

    def __init__(self, what: str, vehicle: str, timeout: float, detail: str = ""):
        self.what, self.vehicle, self.timeout = what, vehicle, timeout
        extra = f" ({detail})" if detail else ""
        super().__init__(f"{vehicle}: timed out after {timeout:g} s waiting for {what}{extra}")


class WrongAutopilot(MavlinkError):
    """The vehicle reports another autopilot than the one its driver flies (e.g. MAVSDK finds ArduPilot)."""

    def __init__(self, vehicle: str, reported: str, flies: str):
        self.vehicle, self.reported, self.flies = vehicle, reported, flies
        super().__init__(f"{vehicle}: the vehicle reports autopilot {reported}; this driver flies {flies}")


class NotReady(WaitTimeout):
    """A vehicle that did not become ready to arm in time; the message names the last reason it gave."""

    def __init__(self, vehicle: str, timeout: float, reason: str):
        self.what, self.vehicle, self.reason, self.timeout = "ready to arm", vehicle, reason, timeout
        MavlinkError.__init__(self, f"{vehicle}: not ready to arm after {timeout:g} s: {reason}")
