"""The robot emulator in a process of its own, so that it does not share the interpreter lock with a Python client."""

from __future__ import annotations

import multiprocessing
import signal
import threading
from typing import Any

from iiwa_ident.emulator._config import EmulatorConfig, check_config
from iiwa_ident.emulator._report import EmulatorReport
from iiwa_ident.emulator._robot_side import RobotEmulator
from iiwa_ident.errors import IiwaIdentError

__all__ = ["EmulatorProcess", "spawn_emulator"]


def _watch_stop(conn, emulator: RobotEmulator) -> None:
    """Stop the emulator on a message from the parent, or when the parent has gone (EOF)."""
    try:
        conn.recv()
    except (EOFError, OSError):
        pass
    emulator.stop()


def _child_main(config: EmulatorConfig, conn, stop_conn) -> None:
    """Entry point of the emulator process: report the address, run, send the report."""
    try:
        emulator = RobotEmulator(config)
    except Exception as err:  # noqa: BLE001  (any failure must reach the parent as a message)
        conn.send(("error", str(err) if isinstance(err, IiwaIdentError) else f"{type(err).__name__}: {err}"))
        conn.close()
        return
    # Ctrl-C reaches the whole process group: close the session cleanly instead of dying.
    signal.signal(signal.SIGINT, lambda *_: emulator.stop())
    signal.signal(signal.SIGTERM, lambda *_: emulator.stop())
    threading.Thread(target=_watch_stop, args=(stop_conn, emulator), daemon=True).start()
    conn.send(("address", emulator.address))
    message: tuple[str, str | EmulatorReport]
    try:
        report = emulator.run()
    except Exception as err:  # noqa: BLE001  (any failure must reach the parent as a message)
        message = ("error", f"emulator failed: {type(err).__name__}: {err}")
    else:
        message = ("report", report)
    try:
        conn.send(message)
    except OSError:
        pass  # the parent has gone
    conn.close()


class EmulatorProcess:
    """A :class:`RobotEmulator` running in its own process (see :func:`spawn_emulator`).

    Attributes
    ----------
    address : (str, int)
        The robot-side socket's address.
    """

    def __init__(self, config: EmulatorConfig, start_timeout_s: float = 60.0) -> None:
        check_config(config)
        ctx = multiprocessing.get_context("spawn")
        # Two one-way pipes: the child's messages, and the stop request. (A multiprocessing
        # Event would hang the parent's set() once the waiting child has exited.)
        self._conn, child_conn = ctx.Pipe(duplex=False)
        stop_reader, self._stop_conn = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=_child_main, args=(config, child_conn, stop_reader),
                                    name="iiwa-fri-emulator", daemon=True)
        self._process.start()
        child_conn.close()
        stop_reader.close()
        self._report: EmulatorReport | None = None
        try:
            kind, value = self._receive(start_timeout_s, "start")
        except IiwaIdentError:
            self._shut_down()
            raise
        if kind != "address":
            self._shut_down()
            raise IiwaIdentError(value)
        self.address: tuple[str, int] = tuple(value)

    def _shut_down(self) -> None:
        """End the process if it still runs (SIGTERM stops the emulator cleanly) and close the pipes."""
        self._process.join(5.0 if self._report is not None else 0.5)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(5.0)
        self._conn.close()
        self._stop_conn.close()

    def _receive(self, timeout: float | None, what: str) -> tuple[str, Any]:
        try:
            ready = self._conn.poll(timeout)
        except (OSError, EOFError):
            ready = True
        if not ready:
            raise IiwaIdentError(f"the emulator process did not {what} within {timeout:g} s")
        try:
            return self._conn.recv()
        except (EOFError, OSError):
            self._process.join(5.0)
            raise IiwaIdentError(f"the emulator process exited (code {self._process.exitcode}) "
                                 f"before it could {what}") from None

    def stop(self) -> None:
        """Ask the emulator to close the session and end."""
        try:
            self._stop_conn.send("stop")
        except (OSError, ValueError):
            pass  # the process has ended already (or the pipe is closed)

    def join(self, timeout: float | None = None) -> EmulatorReport:
        """Wait for the run to end and return its report.

        Parameters
        ----------
        timeout : float or None
            Longest wait [s]; None waits as long as it takes.

        Raises
        ------
        IiwaIdentError
            If the run does not end in time or the process fails.
        """
        if self._report is None:
            kind, value = self._receive(timeout, "finish")
            if kind != "report":
                self._process.join(5.0)
                raise IiwaIdentError(value)
            self._report = value
            self._process.join(5.0)
        return self._report

    def kill(self) -> None:
        """End the emulator process at once (SIGKILL), as a robot that vanishes: nothing more is sent.

        No report follows; :meth:`join` then raises.
        """
        self._process.kill()
        self._process.join(5.0)

    @property
    def alive(self) -> bool:
        """Whether the emulator process is still running."""
        return self._process.is_alive()

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        try:
            self.join(10.0)
        except IiwaIdentError:
            pass
        finally:
            self._shut_down()


def spawn_emulator(config: EmulatorConfig, start_timeout_s: float = 60.0) -> EmulatorProcess:
    """Start a :class:`RobotEmulator` in a separate process.

    The emulator gets its own interpreter (``spawn`` start method), so it
    does not share the GIL with the client under test.

    Parameters
    ----------
    config : EmulatorConfig
        Settings (must be picklable; the default plant is).
    start_timeout_s : float
        Longest wait for the process to import and bind its socket [s].

    Returns
    -------
    EmulatorProcess
        Running; its ``address`` is known. Use it as a context manager, or
        call ``stop()`` and ``join()``.

    Raises
    ------
    IiwaIdentError
        For a bad setting, a socket that cannot be bound, or a process that
        does not start.
    """
    return EmulatorProcess(config, start_timeout_s)
