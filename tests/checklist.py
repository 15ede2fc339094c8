"""The small runner the Python tests under ctest share: `test(fn)` (also as a decorator) runs one
check, reports it and keeps going; `finish()` prints the closing 'N passed, N failed' line CI reads
and exits 1 if any check failed."""
import sys

results = []


def test(fn):
    try:
        fn()
        results.append((fn.__name__, None))
        print(f"ok   {fn.__name__}")
    except Exception as e:  # noqa: BLE001 - report every failure, keep going
        results.append((fn.__name__, e))
        print(f"FAIL {fn.__name__}: {type(e).__name__}: {e}")
    return fn


def finish():
    failed = sum(1 for _, e in results if e)
    print(f"{len(results) - failed} passed, {failed} failed")
    sys.exit(1 if failed else 0)
