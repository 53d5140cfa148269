"""A blocking facade of the shaker amplifier driver (:class:`drivers.amplifier.ShakerAmplifier`),
for callers that are not async: the driver runs on a private event loop in a daemon thread,
its status monitor going on between calls.

Split from ``drivers.amplifier`` (which passed 500 lines) along the seam between the device
and the way it is called; behaviour unchanged.
"""

from __future__ import annotations

import asyncio
import threading

from .amplifier import AmpStatus, ShakerAmplifier
from .errors import InstrumentTimeout
from .interrupts import future_result, interrupts_held

__all__ = ["SyncShakerAmplifier"]


class SyncShakerAmplifier:
    """Blocking facade of :class:`ShakerAmplifier` (its own event loop in a daemon thread).

    Takes the same arguments. Every call has a deadline, so a dead link raises instead of
    hanging. Use as a context manager; exit always reaches the safe state.
    """

    def __init__(self, *args, **kwargs) -> None:
        self.amp = ShakerAmplifier(*args, **kwargs)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name=f"amp-{self.amp.name}", daemon=True)
        self._thread.start()
        try:
            self._call(self.amp.connect())
        except BaseException:
            with interrupts_held:
                self._shutdown_loop()
            raise

    def _call(self, coro, timeout_s: float | None = None):
        fut = asyncio.run_coroutine_threadsafe(coro, self._loop)
        # A hang guard: beyond the requests' own time-outs, and the waits for an amplifier to
        # answer again after a late reply (the safe state may make two).
        a = self.amp
        deadline = timeout_s if timeout_s is not None else 10 * (a.retries + 1) * a.timeout_s + 2 * a.resync_s + 5.0
        try:
            # In slices with Ctrl-C held: an interrupt inside Future.result's condition could
            # leave it locked and the event loop's thread stuck setting the result.
            return future_result(fut, deadline)
        except TimeoutError:
            if fut.done():
                raise  # the call's own InstrumentTimeout (a TimeoutError too), with its own words
            fut.cancel()
            raise InstrumentTimeout(f"{self.amp.name}: call did not finish within {deadline:g} s") from None
        except BaseException:
            # A Ctrl-C: the call must not go on behind the caller's back (an enable() that
            # finished after the safe state had disabled the amplifier re-enabled it).
            fut.cancel()
            raise

    def read_status(self) -> AmpStatus:
        return self._call(self.amp.read_status())

    def enable(self) -> None:
        self._call(self.amp.enable())

    def disable(self) -> None:
        self._call(self.amp.disable())

    def set_gain(self, gain_v_per_v: float) -> None:
        self._call(self.amp.set_gain(gain_v_per_v))

    def reset_fault(self) -> None:
        self._call(self.amp.reset_fault())

    def check(self) -> None:
        self.amp.check()

    def safe_state(self) -> None:
        self._call(self.amp.safe_state())

    def close(self) -> None:
        """Safe state, then end the link and the event loop. A Ctrl-C meanwhile is raised
        when both are done: it cancelled the safe state, the amplifier stayed enabled, and
        the loop it stopped left a second ``close()`` nothing to do it with."""
        if not self._thread.is_alive():
            return
        with interrupts_held:
            try:
                self._call(self.amp.close())
            finally:
                self._shutdown_loop()

    def release(self) -> None:
        """Close the link without another safe state (as ``SignalGenerator.release``); the
        amplifier's own comms watchdog disables it once the link is gone."""
        if not self._thread.is_alive():
            return
        with interrupts_held:
            try:
                self._call(self.amp.close(safe_state=False))
            finally:
                self._shutdown_loop()

    def _shutdown_loop(self) -> None:
        async def cancel_the_rest() -> None:
            # Tasks the library still runs (a reconnect after a dropped link) are cancelled
            # and given the loop to end in, not destroyed pending with the loop.
            rest = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in rest:
                t.cancel()
            await asyncio.gather(*rest, return_exceptions=True)

        if self._thread.is_alive():
            try:
                asyncio.run_coroutine_threadsafe(cancel_the_rest(), self._loop).result(timeout=2.0)
            except Exception:  # noqa: BLE001 -- shutting down: the loop is stopped below anyway
                pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5.0)
        if not self._thread.is_alive():
            self._loop.close()

    def __enter__(self) -> SyncShakerAmplifier:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
