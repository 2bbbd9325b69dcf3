"""The normal equations' block sums in LLVM vector instructions, the same bits as the scalar sums.

LM's J^T W J sums, for each pair of echoes, 16 products a sample (4 columns by 4) into 16 accumulators, each in
sample order. LLVM does not vectorize that loop (its accumulators are not a reduction it may reorder, nor a store
chain its SLP pass seeds from), so each product was a scalar multiply and add. Here a sample's 16 products are
two 8-lane multiplies of a column quadruple's broadcast lanes by the other quadruple, added lane by lane to the
same 16 accumulators: each lane does exactly the scalar expression's operations, in the same order (IEEE
arithmetic has no lane effects and the kernels never fuse a multiply into an add), so every sum is the scalar
loop's to the bit, on any machine LLVM targets.

`block_sums(jac, weights, residual, lo, hi, r, c)`, over samples lo..hi-1, one tuple of 24 floats:

- [4 a + b]: sum ((jac[i, r + a] jac[i, c + b]) w_i) w_i, a pair block (r != c) or an echo's own (r == c);
- [16 + a]: sum (jac[i, r + a] w_i) residual_i, an echo's gradient entries (0 where residual is None);
- [20 + a]: sum (jac[i, r + a] w_i) w_i, its rows with the background's column (0 where residual is None).

`weighted_block_sums` is the same for rows of W^1/2 J (already weighted): j j, j residual and j w.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_F64 = ir.DoubleType()
_V4 = ir.VectorType(_F64, 4)
_V8 = ir.VectorType(_F64, 8)
_I32 = ir.IntType(32)


def _mask(lanes):
    return ir.Constant(ir.VectorType(_I32, len(lanes)), [ir.Constant(_I32, k) for k in lanes])


_ROWS_LO, _ROWS_HI = _mask([0, 0, 0, 0, 1, 1, 1, 1]), _mask([2, 2, 2, 2, 3, 3, 3, 3])  # lanes a of 4 a + b
_COLUMNS = _mask([0, 1, 2, 3, 0, 1, 2, 3])  # lanes b
_BROADCAST4, _BROADCAST8 = _mask([0] * 4), _mask([0] * 8)


def _check_rows(jac) -> None:
    """Rows read as vectors: contiguous float64 rows."""
    if not (isinstance(jac, types.Array) and jac.ndim == 2 and jac.dtype == types.float64 and jac.layout == "C"):
        raise TypeError(f"the vector lanes need a C-contiguous 2-d float64 array, not {jac}")


def _row_quad(builder, data, row_offset, column):
    """jac[i, column..column + 3] as one vector (row_offset: i's byte offset)."""
    offset = builder.add(row_offset, builder.mul(column, ir.Constant(column.type, 8)))
    address = builder.gep(data, [offset])
    return builder.load(builder.bitcast(address, _V4.as_pointer()), align=8)


def _element(builder, data, stride, i):
    return builder.load(builder.bitcast(builder.gep(data, [builder.mul(i, stride)]), _F64.as_pointer()))


def _broadcast(builder, value, mask):
    vector = builder.insert_element(ir.Constant(ir.VectorType(_F64, len(mask.constant)), None), value,
                                    ir.Constant(_I32, 0))
    return builder.shuffle_vector(vector, vector, mask)


def _array_parts(context, builder, array_type, value):
    array = context.make_array(array_type)(context, builder, value)
    data = builder.bitcast(array.data, ir.IntType(8).as_pointer())
    return data, cgutils.unpack_tuple(builder, array.strides, array_type.ndim)


def _lanes(builder, vectors):
    return [builder.extract_element(v, ir.Constant(_I32, k)) for v in vectors for k in range(v.type.count)]


def _block_sums(weighted_rows: bool):
    """The intrinsic for rows of J (products times w w) or of W^1/2 J (weighted_rows: no weight in them)."""

    def typer(typingctx, jac, weights, residual, lo, hi, r, c):
        _check_rows(jac)
        with_gradient = not isinstance(residual, types.NoneType)
        sig = types.UniTuple(types.float64, 24)(jac, weights, residual, lo, hi, r, c)

        def codegen(context, builder, signature, args):
            jac_value, weights_value, residual_value, lo_value, hi_value, r_value, c_value = args
            data, (row_stride, _) = _array_parts(context, builder, signature.args[0], jac_value)
            w_data, (w_stride,) = _array_parts(context, builder, signature.args[1], weights_value)
            if with_gradient:
                r_data, (r_stride,) = _array_parts(context, builder, signature.args[2], residual_value)
            r_column, c_column, start, stop = (context.cast(builder, args[k], signature.args[k], types.int64)
                                               for k in (5, 6, 3, 4))
            zero8, zero4 = ir.Constant(_V8, [0.0] * 8), ir.Constant(_V4, [0.0] * 4)
            sums = [cgutils.alloca_once_value(builder, z) for z in (zero8, zero8, zero4, zero4)]
            one = ir.Constant(ir.IntType(64), 1)
            with cgutils.for_range_slice(builder, start, stop, one, inc=True) as (i, _):
                row_offset = builder.mul(i, row_stride)
                rows = _row_quad(builder, data, row_offset, r_column)
                columns = _row_quad(builder, data, row_offset, c_column)
                tiled = builder.shuffle_vector(columns, columns, _COLUMNS)
                products = [builder.fmul(builder.shuffle_vector(rows, rows, lanes), tiled)
                            for lanes in (_ROWS_LO, _ROWS_HI)]
                if with_gradient or not weighted_rows:
                    w = _element(builder, w_data, w_stride, i)
                if not weighted_rows:
                    w8 = _broadcast(builder, w, _BROADCAST8)
                    products = [builder.fmul(builder.fmul(p, w8), w8) for p in products]
                for k in range(2):
                    builder.store(builder.fadd(builder.load(sums[k]), products[k]), sums[k])
                if with_gradient:
                    w4 = _broadcast(builder, w, _BROADCAST4)
                    residual4 = _broadcast(builder, _element(builder, r_data, r_stride, i), _BROADCAST4)
                    base = rows if weighted_rows else builder.fmul(rows, w4)  # j, or j w
                    builder.store(builder.fadd(builder.load(sums[2]), builder.fmul(base, residual4)), sums[2])
                    builder.store(builder.fadd(builder.load(sums[3]), builder.fmul(base, w4)), sums[3])
            values = _lanes(builder, [builder.load(s) for s in sums])
            return context.make_tuple(builder, signature.return_type, values)

        return sig, codegen

    typer.__name__ = "weighted_block_sums" if weighted_rows else "block_sums"
    return intrinsic(typer)


# rows of J: outer[4 a + b] = sum ((j_a j_b) w) w, with_residual = sum (j w) r, with_weight = sum (j w) w
block_sums = _block_sums(weighted_rows=False)
# rows of W^1/2 J: outer = sum j_a j_b, with_residual = sum j r, with_weight = sum j w
weighted_block_sums = _block_sums(weighted_rows=True)


CHOLESKY_LANES = 8


@intrinsic
def cholesky_lanes(typingctx, factor, c, r, pivot):
    """Entries r..r + 7 of column c of a Cholesky factor kept transposed (factor[q, r] = L[r, q]), in place:
    factor[c, r + k] = (factor[c, r + k] - sum over q < c of factor[q, r + k] factor[q, c]) / pivot, the
    subtractions in q order in each lane, as the scalar loop takes them."""
    _check_rows(factor)
    sig = types.void(factor, c, r, pivot)

    def codegen(context, builder, signature, args):
        data, (row_stride, _) = _array_parts(context, builder, signature.args[0], args[0])
        column, first = (context.cast(builder, args[k], signature.args[k], types.int64) for k in (1, 2))
        eight = ir.Constant(ir.IntType(64), 8)
        address = builder.gep(data, [builder.add(builder.mul(column, row_stride), builder.mul(first, eight))])
        target = builder.bitcast(address, _V8.as_pointer())
        sums = cgutils.alloca_once_value(builder, builder.load(target, align=8))
        zero, one = ir.Constant(ir.IntType(64), 0), ir.Constant(ir.IntType(64), 1)
        with cgutils.for_range_slice(builder, zero, column, one, inc=True) as (q, _):
            row = builder.mul(q, row_stride)
            lanes = builder.load(builder.bitcast(builder.gep(data, [builder.add(row, builder.mul(first, eight))]),
                                                 _V8.as_pointer()), align=8)
            x = builder.load(builder.bitcast(builder.gep(data, [builder.add(row, builder.mul(column, eight))]),
                                             _F64.as_pointer()))
            builder.store(builder.fsub(builder.load(sums), builder.fmul(lanes, _broadcast(builder, x, _BROADCAST8))),
                          sums)
        divisor = _broadcast(builder, context.cast(builder, args[3], signature.args[3], types.float64), _BROADCAST8)
        builder.store(builder.fdiv(builder.load(sums), divisor), target, align=8)
        return context.get_dummy_value()

    return sig, codegen
