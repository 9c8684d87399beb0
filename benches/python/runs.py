#!/usr/bin/env python3
"""Runs for timing the Python package as a whole process (docs/benchmarks.md, "Python").

    python runs.py one IMAGE OUT.svg           # as `covec vectorize IMAGE -o OUT.svg`: the SVG
                                               # and the JSON scene beside it, all cores
    python runs.py serial IMAGE...             # the images one after another, all cores each
    python runs.py threads IMAGE...            # one Python thread per image, all at once,
                                               # sharing the process's pool of all cores
    python runs.py threads1 IMAGE...           # the same, each run on a thread of its own

Run it with the Python that has the covec wheel installed.
"""
import os
import sys
import threading

import covec


def run_all(images, **options):
    results = [None] * len(images)

    def run(k):
        results[k] = covec.vectorize(images[k], **options).svg()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(len(images))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert all(results)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    how, args = sys.argv[1], sys.argv[2:]
    if how == "one":
        image, out = args
        result = covec.vectorize(image)
        result.save(out)
        result.save(os.path.splitext(out)[0] + ".json")
    elif how == "serial":
        for image in args:
            covec.vectorize(image).svg()
    elif how == "threads":
        run_all(args)
    elif how == "threads1":
        run_all(args, threads=1)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
