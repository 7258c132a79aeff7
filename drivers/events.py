"""The events every driver yields (DESIGN §4), defined beside the runtime that consumes them.

`runtime.events` holds the definitions so that `runtime/` never imports `drivers/` (DESIGN §2);
drivers import them from there. This module keeps the `drivers.events` name for users' code.
"""
from runtime.events import Event, Frame, ImuSample

__all__ = ["Event", "Frame", "ImuSample"]
