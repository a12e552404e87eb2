#!/usr/bin/env python3
"""Rewrites a SPIR-V module that uses SPV_NV_cooperative_matrix into the same module on
SPV_KHR_cooperative_matrix, the vendor-neutral extension (build step of
cmake/EmbedShaders.cmake for shaders with a '//! spirv coopmat-khr' line).

Why: Debian 12's glslang (12.0) compiles GL_NV_cooperative_matrix but not
GL_KHR_cooperative_matrix (glslang 13+). The two SPIR-V extensions differ only in:
  - the capability (CooperativeMatrixNV 5357 -> CooperativeMatrixKHR 6022) and extension name;
  - the matrix type, which in KHR also names its use (A, B or accumulator): here taken from the
    type's shape, so a shader must declare A as rows x K, B as K x columns and the
    accumulator as rows x columns with three distinct specialization constants (the shader's
    CM_M, CM_N, CM_K), and the accumulator with 32-bit, A and B with 16-bit components;
  - load / store operands: NV (pointer, stride, column-major bool) -> KHR (pointer, layout
    constant RowMajorKHR 0 / ColumnMajorKHR 1, stride); the bool must be a constant;
  - opcode numbers of the type, load, store, multiply-add and length instructions.
Anything else in the module is copied word for word.

Usage: coopmat_nv_to_khr.py IN.spv OUT (OUT.spv: the module; OUT.h with --vn NAME: a header
holding `const uint32_t NAME[]`, as glslang's --vn writes it)
"""
import struct
import sys

OP_EXTENSION, OP_CAPABILITY, OP_TYPE_INT, OP_TYPE_FLOAT = 10, 17, 21, 22
OP_CONSTANT_TRUE, OP_CONSTANT_FALSE, OP_CONSTANT = 41, 42, 43
OP_SPEC_CONSTANT = 50
OP_DECORATE, DECORATION_SPEC_ID = 71, 1
CAP_NV, CAP_KHR = 5357, 6022
TYPE_NV, LOAD_NV, STORE_NV, MULADD_NV, LENGTH_NV = 5358, 5359, 5360, 5361, 5362
TYPE_KHR, LOAD_KHR, STORE_KHR, MULADD_KHR, LENGTH_KHR = 4456, 4457, 4458, 4459, 4460
USE_A, USE_B, USE_ACC = 0, 1, 2
# The shader's specialization constant ids of the MMA shape (gemm_coopmat.comp).
SPEC_M, SPEC_N, SPEC_K = 20, 21, 22


def words_of_string(s):
    b = s.encode() + b"\0"
    b += b"\0" * (-len(b) % 4)
    return list(struct.unpack(f"<{len(b) // 4}I", b))


def string_of_words(ws):
    b = struct.pack(f"<{len(ws)}I", *ws)
    return b.split(b"\0", 1)[0].decode()


def instructions(words):
    i = 5
    while i < len(words):
        n, op = words[i] >> 16, words[i] & 0xFFFF
        if n == 0:
            raise SystemExit("coopmat_nv_to_khr: malformed SPIR-V (zero-length instruction)")
        yield op, words[i + 1:i + n]
        i += n


def convert(words):
    if words[0] != 0x07230203:
        raise SystemExit("coopmat_nv_to_khr: not a SPIR-V module")
    insts = list(instructions(words))
    spec_ids, bools, uint_type, float_width = {}, {}, None, {}
    for op, a in insts:
        if op == OP_DECORATE and a[1] == DECORATION_SPEC_ID:
            spec_ids[a[0]] = a[2]
        elif op == OP_CONSTANT_TRUE:
            bools[a[1]] = True
        elif op == OP_CONSTANT_FALSE:
            bools[a[1]] = False
        elif op == OP_TYPE_INT and a[1] == 32 and uint_type is None:
            uint_type = a[0]
        elif op == OP_TYPE_FLOAT:
            float_width[a[0]] = a[1]
    if uint_type is None:
        raise SystemExit("coopmat_nv_to_khr: no 32-bit integer type to make constants of")
    bound = words[3]
    const_ids = {}

    def constant(value):  # id of a new 32-bit integer constant
        nonlocal bound
        if value not in const_ids:
            const_ids[value] = bound
            bound += 1
        return const_ids[value]

    def use_of(comp, rows, cols):
        shape = (spec_ids.get(rows), spec_ids.get(cols))
        width = float_width.get(comp)
        if shape == (SPEC_M, SPEC_K) and width == 16:
            return USE_A
        if shape == (SPEC_K, SPEC_N) and width == 16:
            return USE_B
        if shape == (SPEC_M, SPEC_N) and width == 32:
            return USE_ACC
        raise SystemExit(f"coopmat_nv_to_khr: a matrix type of shape {shape} and {width}-bit "
                         "components is neither A (M x K, fp16), B (K x N, fp16) nor the "
                         "accumulator (M x N, fp32)")

    def layout(bool_id):
        if bool_id not in bools:
            raise SystemExit("coopmat_nv_to_khr: a load or store's column-major flag is not a constant")
        return constant(1 if bools[bool_id] else 0)

    out, converted, first_type = [], 0, None
    for op, a in insts:
        if op == OP_CAPABILITY and a[0] == CAP_NV:
            op, a = op, [CAP_KHR]
        elif op == OP_EXTENSION and string_of_words(a) == "SPV_NV_cooperative_matrix":
            a = words_of_string("SPV_KHR_cooperative_matrix")
        elif op == TYPE_NV:  # result, component, scope, rows, cols
            if first_type is None:
                first_type = len(out)
            op, a = TYPE_KHR, a + [constant(use_of(a[1], a[3], a[4]))]
        elif op == LOAD_NV:  # type, result, pointer, stride, column-major [, memory access...]
            op, a = LOAD_KHR, [a[0], a[1], a[2], layout(a[4]), a[3]] + a[5:]
        elif op == STORE_NV:  # pointer, object, stride, column-major [, memory access...]
            op, a = STORE_KHR, [a[0], a[1], layout(a[3]), a[2]] + a[4:]
        elif op == MULADD_NV:
            op = MULADD_KHR
        elif op == LENGTH_NV:
            op = LENGTH_KHR
        else:
            out.append((op, a))
            continue
        converted += 1
        out.append((op, a))
    if first_type is None:
        raise SystemExit("coopmat_nv_to_khr: the module has no cooperative matrix type")
    # The new constants go right before the first matrix type (after the integer type).
    consts = [(OP_CONSTANT, [uint_type, cid, value]) for value, cid in sorted(const_ids.items())]
    out[first_type:first_type] = consts
    result = words[:5]
    result[3] = bound
    for op, a in out:
        result.append(((len(a) + 1) << 16) | op)
        result.extend(a)
    return result


def main(argv):
    args = argv[1:]
    name = None
    if len(args) == 4 and args[2] == "--vn":
        name = args[3]
        args = args[:2]
    if len(args) != 2:
        raise SystemExit(__doc__)
    data = open(args[0], "rb").read()
    words = list(struct.unpack(f"<{len(data) // 4}I", data))
    out = convert(words)
    if name is None:
        with open(args[1], "wb") as f:
            f.write(struct.pack(f"<{len(out)}I", *out))
        return 0
    lines = [",".join(f"0x{w:08x}" for w in out[i:i + 8]) for i in range(0, len(out), 8)]
    with open(args[1], "w") as f:
        f.write("// Generated by cmake/coopmat_nv_to_khr.py: do not edit.\n#pragma once\n")
        f.write(f"const uint32_t {name}[] = {{\n\t" + ",\n\t".join(lines) + "\n};\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
