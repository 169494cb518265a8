// A dropped folder of frames becomes one recording: the server takes one file per recording, so the folder is
// packed here into a ZIP without compression (frames are PNG/TIFF/JPEG already). The result is a Blob made of the
// original File objects between small headers, so nothing is copied into memory and the upload streams it from
// disk; the files are read once for their CRC-32 (small ones together, large ones in slices). Any size and any
// number of files: past the plain ZIP limits (4 GiB of data or offsets, 65,535 entries) the archive carries ZIP64
// records (APPNOTE 4.5.3, 4.3.14), which Python's zipfile (the server) and every current unzip tool read.

const LIMIT_32 = 0xffffffff; // a 32-bit field holding this value means "see the ZIP64 extra field"
const LIMIT_16 = 0xffff;
const SLICE_BYTES = 8 * 1024 * 1024;

let crcTable = null;
function crc32Table() {
  if (crcTable) return crcTable;
  crcTable = new Uint32Array(256);
  for (let n = 0; n < 256; n += 1) {
    let c = n;
    for (let k = 0; k < 8; k += 1) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    crcTable[n] = c >>> 0;
  }
  return crcTable;
}

/** The running CRC-32 (the ZIP one, pre- and post-inverted by the caller) over `bytes`. */
function crc32Update(crc, bytes) {
  const table = crc32Table();
  for (let i = 0; i < bytes.length; i += 1) crc = table[(crc ^ bytes[i]) & 0xff] ^ (crc >>> 8);
  return crc;
}

/** CRC-32 of a File or Blob, read in slices. */
async function crc32(blob) {
  let crc = 0xffffffff;
  for (let start = 0; start < blob.size; start += SLICE_BYTES) {
    crc = crc32Update(crc, new Uint8Array(await blob.slice(start, start + SLICE_BYTES).arrayBuffer()));
  }
  return (crc ^ 0xffffffff) >>> 0;
}

/**
 * The CRC-32 of every entry's file; `onProgress(doneBytes, totalBytes)`. Files smaller than a slice are read
 * together, a slice's worth in one read: each read waits on the browser's blob store (about half a millisecond, so
 * 100,000 small frames read one by one would wait about a minute for that alone).
 */
async function entryCrcs(entries, onProgress) {
  const total = entries.reduce((sum, e) => sum + e.file.size, 0);
  const crcs = [];
  let done = 0;
  let batch = [];
  let batchBytes = 0;
  const advance = (bytes) => {
    done += bytes;
    onProgress(done, total);
  };
  const readBatch = async () => {
    if (!batch.length) return;
    const bytes = new Uint8Array(await new Blob(batch).arrayBuffer());
    let start = 0;
    for (const file of batch) {
      crcs.push((crc32Update(0xffffffff, bytes.subarray(start, start + file.size)) ^ 0xffffffff) >>> 0);
      start += file.size;
    }
    advance(batchBytes);
    batch = [];
    batchBytes = 0;
  };
  for (const { file } of entries) {
    if (file.size >= SLICE_BYTES) {
      await readBatch();
      crcs.push(await crc32(file));
      advance(file.size);
      continue;
    }
    if (batchBytes + file.size > SLICE_BYTES) await readBatch();
    batch.push(file);
    batchBytes += file.size;
  }
  await readBatch();
  return crcs;
}

/** The bytes of `buffers` (ArrayBuffers or typed arrays) one after the other, in one Uint8Array. */
function joined(buffers) {
  const out = new Uint8Array(buffers.reduce((sum, b) => sum + b.byteLength, 0));
  let at = 0;
  for (const b of buffers) {
    out.set(b instanceof ArrayBuffer ? new Uint8Array(b) : b, at);
    at += b.byteLength;
  }
  return out;
}

function dosDateTime(date) {
  const time = (date.getHours() << 11) | (date.getMinutes() << 5) | Math.floor(date.getSeconds() / 2);
  const day = ((date.getFullYear() - 1980) << 9) | ((date.getMonth() + 1) << 5) | date.getDate();
  return { time, day };
}

/** A ZIP64 extended-information extra field (header id 1) holding the given 8-byte values, in order. */
function zip64Extra(values) {
  const extra = new DataView(new ArrayBuffer(4 + 8 * values.length));
  extra.setUint16(0, 0x0001, true);
  extra.setUint16(2, 8 * values.length, true);
  values.forEach((value, i) => extra.setBigUint64(4 + 8 * i, BigInt(value), true));
  return extra.buffer;
}

/**
 * A stored (uncompressed) ZIP of `entries` = [{ path, file }] as a Blob; `path` uses "/" and is stored as UTF-8.
 * `onProgress(doneBytes, totalBytes)` follows the CRC reading. ZIP64 records are written where a size, an offset
 * or the entry count passes the plain ZIP fields, or everywhere with `zip64: "always"` (for tests).
 */
export async function storedZip(entries, { onProgress = () => {}, zip64 = "auto" } = {}) {
  const always = zip64 === "always";
  const encoder = new TextEncoder();
  const crcs = await entryCrcs(entries, onProgress);
  const parts = [];
  const central = [];
  let offset = 0;
  entries.forEach(({ path, file }, index) => {
    const name = encoder.encode(path);
    const crc = crcs[index];
    const { time, day } = dosDateTime(new Date(file.lastModified || Date.now()));
    const bigSize = always || file.size >= LIMIT_32;
    const bigOffset = always || offset >= LIMIT_32;
    const localExtra = bigSize ? zip64Extra([file.size, file.size]) : new ArrayBuffer(0);
    const local = new DataView(new ArrayBuffer(30));
    local.setUint32(0, 0x04034b50, true);
    local.setUint16(4, bigSize ? 45 : 20, true); // version needed: 4.5 for ZIP64
    local.setUint16(6, 0x0800, true); // UTF-8 names
    local.setUint16(8, 0, true); // stored
    local.setUint16(10, time, true);
    local.setUint16(12, day, true);
    local.setUint32(14, crc, true);
    local.setUint32(18, bigSize ? LIMIT_32 : file.size, true);
    local.setUint32(22, bigSize ? LIMIT_32 : file.size, true);
    local.setUint16(26, name.length, true);
    local.setUint16(28, localExtra.byteLength, true);
    parts.push(joined([local.buffer, name, localExtra]), file); // each Blob part costs the browser's blob store
    const centralValues = [...(bigSize ? [file.size, file.size] : []), ...(bigOffset ? [offset] : [])];
    const centralExtra = centralValues.length ? zip64Extra(centralValues) : new ArrayBuffer(0);
    const header = new DataView(new ArrayBuffer(46));
    header.setUint32(0, 0x02014b50, true);
    header.setUint16(4, 45, true); // made by
    header.setUint16(6, bigSize || bigOffset ? 45 : 20, true);
    header.setUint16(8, 0x0800, true);
    header.setUint16(10, 0, true);
    header.setUint16(12, time, true);
    header.setUint16(14, day, true);
    header.setUint32(16, crc, true);
    header.setUint32(20, bigSize ? LIMIT_32 : file.size, true);
    header.setUint32(24, bigSize ? LIMIT_32 : file.size, true);
    header.setUint16(28, name.length, true);
    header.setUint16(30, centralExtra.byteLength, true);
    header.setUint32(42, bigOffset ? LIMIT_32 : offset, true);
    central.push(header.buffer, name, centralExtra);
    offset += 30 + name.length + localExtra.byteLength + file.size;
  });
  const centralDirectory = joined(central);
  const centralSize = centralDirectory.byteLength;
  const centralOffset = offset;
  const count = entries.length;
  const big = always || count >= LIMIT_16 || centralOffset >= LIMIT_32 || centralSize >= LIMIT_32;
  const tail = [];
  if (big) {
    const record = new DataView(new ArrayBuffer(56)); // ZIP64 end of central directory record
    record.setUint32(0, 0x06064b50, true);
    record.setBigUint64(4, 44n, true); // size of the rest of the record
    record.setUint16(12, 45, true);
    record.setUint16(14, 45, true);
    record.setBigUint64(24, BigInt(count), true);
    record.setBigUint64(32, BigInt(count), true);
    record.setBigUint64(40, BigInt(centralSize), true);
    record.setBigUint64(48, BigInt(centralOffset), true);
    const locator = new DataView(new ArrayBuffer(20)); // ZIP64 end of central directory locator
    locator.setUint32(0, 0x07064b50, true);
    locator.setBigUint64(8, BigInt(centralOffset + centralSize), true);
    locator.setUint32(16, 1, true); // total number of disks
    tail.push(record.buffer, locator.buffer);
  }
  const end = new DataView(new ArrayBuffer(22));
  end.setUint32(0, 0x06054b50, true);
  end.setUint16(8, big ? LIMIT_16 : count, true);
  end.setUint16(10, big ? LIMIT_16 : count, true);
  end.setUint32(12, big ? LIMIT_32 : centralSize, true);
  end.setUint32(16, big ? LIMIT_32 : centralOffset, true);
  return new Blob([...parts, centralDirectory, ...tail, end.buffer], { type: "application/zip" });
}
