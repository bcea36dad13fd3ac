"""What went wrong while decoding an input that was processed anyway: :class:`InputDamage`.

A file cut short, a stream that breaks off, data the decoder cannot read:
by default processing goes on wherever the decoder can (a packet it cannot
decode is skipped, a frame it decodes with errors is kept, the input ends
where the data ends) and :meth:`InputDamage.describe` says what happened,
for the run's summary.  With ``strict`` the first such event is an
:class:`~fastdet.errors.InputError` instead.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError


@dataclass
class InputDamage:
    """Damage met while decoding one input.

    Parameters
    ----------
    name : str
        The input, for messages.
    strict : bool
        Raise :class:`InputError` at the first damage instead of recording it.

    Attributes
    ----------
    expected : int or None
        Frames the input should give (from its index), when known.
    ended_after : int or None
        The last frame read when the input ended before ``expected``
        frames; ``None`` when it did not.
    undecodable : int
        Packets the decoder could not decode (skipped).
    corrupt : int
        Frames the decoder returned with errors concealed (kept).
    """

    name: str
    strict: bool = True
    expected: int | None = None
    ended_after: int | None = None
    undecodable: int = 0
    corrupt: int = 0
    _first_undecodable: tuple | None = None   # (last frame before it, reason)
    _first_corrupt: int | None = None
    _end_reason: str | None = None

    def __bool__(self):
        return self.ended_after is not None or bool(self.undecodable or self.corrupt)

    def ended_early(self, last_frame, reason=None):
        """The input ended after ``last_frame``: before :attr:`expected` frames, or as
        reading failed for ``reason``."""
        self.ended_after, self._end_reason = last_frame, reason
        if self.strict and reason:
            raise InputError(f"{self.name}: reading failed {_after(last_frame)}: {reason}")
        if self.strict:
            raise InputError(f"{self.name}: the input ends {_after(last_frame)} of "
                             f"{self.expected} frames (truncated or damaged)")

    def undecodable_packet(self, last_frame, reason):
        """The decoder could not decode a packet after frame ``last_frame``."""
        self.undecodable += 1
        if self._first_undecodable is None:
            self._first_undecodable = (last_frame, reason)
        if self.strict:
            raise InputError(f"{self.name}: decoding failed {_after(last_frame)}: {reason}")

    def corrupt_frame(self, index):
        """Frame ``index`` was decoded with errors (``frame.is_corrupt``)."""
        self.corrupt += 1
        if self._first_corrupt is None:
            self._first_corrupt = index
        if self.strict:
            raise InputError(f"{self.name}: frame {index} is damaged (decoded with errors)")

    def describe(self, frames_read):
        """One phrase for the summary: frames read and where decoding failed (``''``: none).

        Parameters
        ----------
        frames_read : int
            Frames the input gave.
        """
        if not self:
            return ""
        total = f" of {self.expected}" if self.expected is not None else ""
        parts = [f"input damaged: read {frames_read}{total} frames"]
        if self._first_undecodable is not None:
            last, reason = self._first_undecodable
            packets = "packet" if self.undecodable == 1 else "packets"
            parts.append(f"decoding failed {_after(last)} ({reason}; {self.undecodable} "
                         f"{packets} skipped)")
        # Frames missing because packets were skipped need no second mention.
        unexplained = self._end_reason or (self.expected or 0) - frames_read > self.undecodable
        if self.ended_after is not None and unexplained:
            why = f" ({self._end_reason})" if self._end_reason else ""
            parts.append(f"the input ends {_after(self.ended_after)}{why}")
        if self.corrupt:
            frames = "frame" if self.corrupt == 1 else "frames"
            parts.append(f"{self.corrupt} {frames} decoded with errors (the first: frame "
                         f"{self._first_corrupt})")
        return ", ".join(parts)


def _after(last_frame):
    return "before the first frame" if last_frame < 0 else f"after frame {last_frame}"
