"""Dr.Jit 1.5.0: a frozen function replays a recording made for another Python value.

``dr.freeze`` keys its recordings on the input PyTree, with the values of its Python
leaves (ints, strings, ...) compared by equality. But the traversal deduplicates: an
object met a second time in the same call's inputs is stored as a back-reference
(``LayoutFlag::RecursiveRef``, ``TraverseContext::deduplicate_pytree``) and its value
is not part of the key. CPython shares one object per small int (-5 .. 256), so an int
argument equal to any int met earlier in the inputs (a matrix view's shape, an
offset, ...) is not compared: two calls that differ only in it hit the same recording,
and the replay runs the first call's kernels, with their sizes, on the second call's
arrays.

Run with the project's environment: ``python scripts/drjit_defects/freeze_dedup_key.py``.
It prints, for two calls with ``count`` 25 then 40 (an earlier argument holds 25 and 40):

    count 25: recordings 1, width 25 (expected 25)
    count 40: recordings 1, width 25 (expected 40)    <- the defect

With ``--overflow`` it also runs a scatter of ``count`` values into a buffer of
``count`` entries: the replay allocates the first recording's 25 entries and scatters
all ``count`` values into them, past the end of the allocation. Seen here (Dr.Jit 1.5.0,
``llvm_ad_rgb``): widths 25, 25, 25, 25 for counts 25, 25, 40, 4000, then a
segmentation fault at 400000; smaller overruns corrupt the heap silently and abort
later ("corrupted size vs. prev_size", "corrupted double-linked list").

The project's frozen calls avoid it by handing Dr.Jit a key object made anew for each
call (renderers/frozen.py, ``CallKey``): a new object is never a back-reference.
"""

from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi


def main() -> int:
    mi.set_variant("llvm_ad_rgb")

    def zeros(x: mi.Float, shapes: tuple[int, ...], count: int) -> mi.Float:
        return dr.zeros(mi.Float, count) + x

    frozen = dr.freeze(zeros)
    x = mi.Float(1.0)
    shapes = (25, 40)   # e.g. the shapes of an MLP's weight matrices
    wrong = 0
    for count in (25, 40):
        y = frozen(x, shapes, count)
        print(f"count {count}: recordings {frozen.n_recordings}, width {dr.width(y)} "
              f"(expected {count})")
        wrong += dr.width(y) != count

    if "--overflow" in sys.argv:
        def fill(x: mi.Float, index: mi.UInt32, shapes: tuple[int, ...], count: int
                 ) -> mi.Float:
            buffer = dr.zeros(mi.Float, count)   # sized by the Python value
            dr.scatter(buffer, x, index)
            return buffer

        frozen_fill = dr.freeze(fill, auto_opaque=False)
        counts = (25, 25, 40, 4000, 400000)
        for count in counts:
            x, index = dr.opaque(mi.Float, 1.0, count), dr.arange(mi.UInt32, count)
            dr.eval(x, index)
            out = frozen_fill(x, index, counts, count)   # ``counts`` holds every count
            dr.eval(out)
            print(f"fill {count}: recordings {frozen_fill.n_recordings}, width "
                  f"{dr.width(out)} (expected {count})", flush=True)
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
