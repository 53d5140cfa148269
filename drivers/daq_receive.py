"""The receive path of the CAN FD DAQ driver (:class:`drivers.daq.CanFdDaq`): frames pulled
off the bus inside the driver's own calls and routed, and the wait for a block of scans.

:class:`FrameReceiver` is a base class of :class:`~drivers.daq.CanFdDaq` and works on its
state (the bus, the streams, the errors recorded meanwhile); it is not used on its own.
It polls the bus in bounded bulk, puts sample frames into their streams, passes response
frames on to the request that waits for them, ends the streams of a finite acquisition
whose last frames are lost, and raises what the polls recorded (bus-off, lost frames).

Split from ``drivers.daq`` (which passed 500 lines) along the seam between the frames coming
in and the requests, configuration and acquisition control going out; behaviour unchanged.
"""

from __future__ import annotations

import logging
import time

import can

from .daq_protocol import DATA_ID0, RSP_ID, ChannelStream
from .errors import BusOff, ConnectionLost, FramesLost, InstrumentError, InstrumentTimeout, StreamError
from .interrupts import interrupts_held

__all__ = ["CAN_ERR_BUSOFF", "END_WAIT_S", "MAX_FRAMES_PER_POLL", "FrameReceiver"]

# The DAQ driver's logger: what the receive path logs is the driver's, under the name
# logging configurations (and the tests) give it.
log = logging.getLogger("drivers.daq")
CAN_ERR_BUSOFF = 0x40
#: Frames one poll of the bus drains at most (11 ms of sample frames measured): a sender faster
#: than the driver must not keep a poll going, and with it a held Ctrl-C or a request's
#: time-out, for as long as it sends.
MAX_FRAMES_PER_POLL = 2048
#: Quiet time after which, once an input's last frame of a finite acquisition is in, the frames
#: still missing are declared lost. The node sends every input's frames of a scan block
#: together, so the others' last frames are on the bus within a few frame times (8 frames,
#: the reorder window, are 1.4 ms at 5 Mbit/s); 0.1 s leaves room for host scheduling and a
#: TCP gateway, and is well under any ``stream_timeout_s`` worth setting.
END_WAIT_S = 0.1


class FrameReceiver:
    """The receive half of :class:`~drivers.daq.CanFdDaq`, which sets the state used here
    (``name``, ``bus``, ``_poll_s``, ``_streams``, ``_errors``, ``_last_data``, ``_stale_frames``,
    ``stream_timeout_s``, ``on_gap``) and provides ``_on_response`` and ``status``.
    """

    # ------------------------------------------------------------------ frames
    def _pump(self, timeout_s: float) -> bool:
        """Receive and dispatch frames for up to ``timeout_s`` (until one arrives). True if one did."""
        try:
            # The virtual bus's receive queue is a lock the simulated DAQ's sending thread
            # also takes: a Ctrl-C must not land inside it (drivers.interrupts).
            with interrupts_held:
                return self._pump_frames(timeout_s)
        except can.CanError as exc:
            raise ConnectionLost(f"{self.name}: CAN interface failed: {exc}") from exc

    def _pump_frames(self, timeout_s: float) -> bool:
        if self._poll_s:
            # In-process bus: blocking recv would wake this thread for every single frame
            # and fight the sending thread for the GIL; sleeping and draining in bulk is
            # several times faster.
            msg = self.bus.recv(0.0)
            if msg is None:
                time.sleep(min(self._poll_s, timeout_s))
                msg = self.bus.recv(0.0)
        else:
            msg = self.bus.recv(timeout_s)
        if msg is None:
            return False
        recv, dispatch, streams = self.bus.recv, self._dispatch, self._streams
        n_data = n_frames = 0
        while msg is not None:
            # Sample frames inline (the hot path); everything else through _dispatch.
            st = None if msg.is_error_frame else streams.get(msg.arbitration_id - DATA_ID0)
            if st is not None and msg.arbitration_id >= DATA_ID0:
                n_data += 1
                gap = st.push(msg.data)
                if gap is not None:
                    self._errors.append(gap)
            else:
                dispatch(msg)
                if msg.arbitration_id == RSP_ID and not msg.is_error_frame:
                    # A response ends the poll: the frames behind it may depend on it. Those
                    # behind START's are the new acquisition's, whose streams start() makes
                    # only once START is answered; taken here they would be dropped.
                    break
            n_frames += 1
            msg = recv(0.0) if n_frames < MAX_FRAMES_PER_POLL else None
        if n_data:
            self._last_data = time.monotonic()
        return True

    def _dispatch(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self._errors.append(BusOff(f"{self.name}: CAN controller reported bus-off"))
            return
        aid = msg.arbitration_id
        st = self._streams.get(aid - DATA_ID0)
        if st is not None and DATA_ID0 <= aid:
            self._last_data = time.monotonic()
            gap = st.push(bytes(msg.data))
            if gap is not None:
                self._errors.append(gap)
        elif aid == RSP_ID:
            self._on_response(bytes(msg.data))
        elif aid >= DATA_ID0:
            self._stale_frames += 1  # an input not streaming now: a frame of an earlier acquisition

    def _await_scans(self, streams: list[ChannelStream], n_scans: int, deadline: float | None,
                     timeout_s: float | None) -> None:
        """Pump the bus until every stream holds ``n_scans`` scans (the wait of
        :meth:`~drivers.daq.CanFdDaq.read`, which documents what it raises)."""
        while min(s.available for s in streams) < n_scans:
            self._raise_errors()
            if all(s.finished for s in streams):
                raise StreamError(f"{self.name}: acquisition ended with {min(s.available for s in streams)} "
                                  f"of {n_scans} scans left")
            if deadline is not None and time.monotonic() > deadline:
                raise InstrumentTimeout(f"{self.name}: {n_scans} scans not complete within {timeout_s:g} s")
            # Listen before judging the stream dead: frames that queued while the caller was
            # away (processing a block, a slow disk) are a live node's, not silence.
            self._pump(0.05)
            if self._end_streams(streams):
                continue
            silent_s = time.monotonic() - self._last_data
            if (silent_s > self.stream_timeout_s and min(s.available for s in streams) < n_scans
                    and not all(s.finished for s in streams)):
                self._raise_errors()  # the controller's own report first, if it sent one
                if self._ended_by_status(streams):
                    continue
                raise BusOff(f"{self.name}: no sample frames for {silent_s:.1f} s "
                             "(DAQ silent, disconnected or bus-off)")

    def _end_streams(self, streams: list[ChannelStream]) -> bool:
        """Declare the frames still missing at the end of a finite acquisition lost.

        No later frame overflows a reorder buffer there, so without this a lost frame near
        the end would wait for ``stream_timeout_s`` and be taken for a silent node. Once
        any input's last frame is in and the bus has been quiet for a short while, every
        frame the node sent has arrived. True if streams were ended.
        """
        quiet_s = time.monotonic() - self._last_data
        if (quiet_s < min(END_WAIT_S, self.stream_timeout_s / 2) or all(s.finished for s in streams)
                or not any(s.saw_end for s in streams)):
            return False
        self._all_sent(streams)
        return True

    def _ended_by_status(self, streams: list[ChannelStream]) -> bool:
        """A finite acquisition gone quiet with no input's last frame in: ask the DAQ.

        If every input lost its last frame, nothing in the stream tells a finished
        acquisition from a dead node; a DAQ that answers "finished" has sent them all, so
        the missing frames were lost. True if it did (the streams are then ended).
        """
        if any(s.total is None for s in streams):
            return False
        try:
            finished = self.status()["state"] == "finished"
        except InstrumentError:
            return False  # no answer either: the node is silent, as the caller reports
        if finished:
            self._all_sent(streams)
        return finished

    def _all_sent(self, streams: list[ChannelStream]) -> None:
        """The node has sent every frame of the acquisition: the ones missing are lost."""
        for s in streams:
            self._errors.extend(s.end())

    def _raise_errors(self) -> None:
        for err in list(self._errors):
            if isinstance(err, FramesLost) and self.on_gap == "mark":
                # A logging handler's lock is taken by every thread that logs (the safe
                # state's too): a Ctrl-C inside its acquire would leave it taken for good.
                self._errors.remove(err)
                with interrupts_held:
                    log.warning("%s", err)
                continue
            self._errors.remove(err)
            raise err
