"""The exceptions covec raises. The extension module raises them too (it imports them from
here), each with covec's own message."""


class Error(Exception):
    """Anything covec refused or could not do; the base of the others."""


class InputError(Error, ValueError):
    """An image, albedo map, mask, label map, reference or scene that covec cannot use: not
    decodable, cut short, empty, too large, of the wrong dtype or shape, or without the image's
    aspect ratio."""


class ParamsError(Error, ValueError):
    """A parameter out of its range (`paths`, `max_size`, `mode`, `threads`, a width)."""


class EditError(Error, ValueError):
    """An edit that cannot apply: an unknown path id, no albedo path at a point, a colour
    outside [0, 1], `k` of 0."""
