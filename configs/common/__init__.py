"""Not code: with the repository on sys.path, gin's package reader finds `include 'configs/common/...'` here.

Without this file, `configs.common` is a namespace package and gin 0.5.0 fails on it (a TypeError) when a
config is loaded from a working directory other than the repository root.
"""
